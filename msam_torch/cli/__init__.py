"""The command line: ``msam run``, ``msam diagnose`` and ``msam report`` (:mod:`.main`) and the types
of their options (:mod:`.argtypes`)."""
