"""The point filters: one module per method (dror, dsor, lior, echo) on the shared base (:mod:`.base`), the
geometry-only fallback, and the checks and scan geometry they share. By name: :mod:`weather_filter.filter_methods`."""
