"""Constants shared by the napari plugin's tests."""

from metasensor.config import SystemConfig

CFG = SystemConfig(nnum=5, scan=5)  # 5 x 5 views, scan step d = 1 px
P_UM = CFG.pixel_pitch * 1e6  # 13.8 µm sensor pixels
