"""Other SLAM systems run beside Canopy on the same frames (optional extras; see orbslam3.py)."""
