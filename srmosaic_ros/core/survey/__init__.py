"""Stills surveys aligned globally: candidate pairs from predicted footprints (pairs.py) and one
robust least-squares solve over every frame's ground homography (global_align.py)."""
