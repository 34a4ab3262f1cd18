"""Disparity and depth from the views."""
