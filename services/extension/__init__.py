"""Services of one's own (docs/extending.md): the public API a user service is written against
(:mod:`services.extension.api`), the loader of ``FILE.py:NAME`` (:mod:`services.extension.loader`)
and how a loaded service runs as any service does (:mod:`services.extension.hosting`); a service
that drives in the built-in drive's place: its core (:mod:`services.extension.driving`) and its
output (:mod:`services.extension.drive_output`)."""
