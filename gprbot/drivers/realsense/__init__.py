"""realsense."""
