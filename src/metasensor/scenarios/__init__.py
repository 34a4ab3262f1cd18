"""The paper's experiments as runnable scenarios: plastic wrap (Fig. 3), the turbulent telescope
(Fig. 5, Extended Data Fig. 8) and the gigapixel mosaic (Extended Data Fig. 7), and their pieces
(phase screens, the annular pupil's estimate)."""
