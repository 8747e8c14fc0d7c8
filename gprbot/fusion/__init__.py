"""Pose estimation: visual odometry, the loosely coupled filter, pose interpolation (pure)."""
