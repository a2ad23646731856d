"""The starting model as the paper writes it (Eq. 2): the spec (:mod:`.spec`), whitelisted expressions
(:mod:`.expressions`) and the notation of an adjusted equation (:mod:`.notation`, Eq. 9)."""
