"""Simulator: raw meta-imaging captures with known truth, built-in scenes, comparison sensors."""
