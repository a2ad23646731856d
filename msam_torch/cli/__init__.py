"""The command line: ``msam run`` and ``msam diagnose`` (:mod:`.main`) and the types
of their options (:mod:`.argtypes`)."""
