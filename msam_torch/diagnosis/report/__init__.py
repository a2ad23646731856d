"""The gap report: the value and its JSON (:mod:`.gap_report`), the Markdown document, its figures and
HTML."""
