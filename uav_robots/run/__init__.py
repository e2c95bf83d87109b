"""`uav-robots run`: a whole mission's processes on this machine, started, watched, stopped, summed up."""
