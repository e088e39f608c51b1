"""The reality gap: compare a recording with its re-simulation (signatures, compare, report) and search the effects that close the gap."""
