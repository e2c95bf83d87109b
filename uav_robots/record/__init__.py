"""Watching a mission and keeping it: the observer, mission.mcap, replay.mp4, report.html, `uav-robots replay`."""
