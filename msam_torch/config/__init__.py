"""The config: its YAML schema (:mod:`.schema`), strategy registries (:mod:`.registry`) and what an
error suggests (:mod:`.suggestions`)."""
