"""The reality gap (entry points in :mod:`.command`): compare a recording with its re-simulation (signatures,
compare, report) and search the effects that close the gap (:mod:`.search` and its rounds)."""
