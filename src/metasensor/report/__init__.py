"""Reports: the demo comparison of the three sensors and its HTML page."""
