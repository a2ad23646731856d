"""The effect catalogue (``catalogue.yaml``) and the names it gives fitted hypotheses within
confidence."""
