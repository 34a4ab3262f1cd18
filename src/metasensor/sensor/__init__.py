"""Sensor geometry: scan orders, realign/unrealign, lenslet-grid calibration, rectification."""
