"""Measurements in: loading records from configs, tables and arrays (:mod:`.loading`, :mod:`.tables`),
records that carry no information (:mod:`.information`), the controlled systems of Table 1
(:mod:`.systems`) and the bundled benchmark records (:mod:`.datasets`)."""
