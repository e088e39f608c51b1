"""Weather generators fixed before use: each written apart from the simulator's model (no import of
``lidar_weather_sim.physics``, ``regions`` or ``sensor.radiometry``) and from the others, each with its
specification in its module docstring, committed with their seeded draw (:mod:`.draw`) before any gap search
was run on them. A generator is never changed after its first run against the search: a new idea is a new
module.

- :mod:`.fog_loss`: fog as two-way Beer-Lambert loss only;
- :mod:`.fog_spread`: the loss plus soft fog echoes spread over 0.6-5 m;
- :mod:`.fog_shell`: the loss plus soft fog echoes in a narrow shell;
- :mod:`.precip_dsd`: rain (gamma DSD) and snow (Sekhon-Srivastava) as discrete drops;
- :mod:`.cover`: a dirty sensor cover as a two-way transmission on every return.

:mod:`.echoes` only reads and writes the project's point layout (received power from intensity and EPW).
"""
