"""The sensor model without a scene: profiles, the scan pattern, the echo decision and its radiometry."""
