"""What more than one wing of the command needs: free ports, robot processes, the run directory, argument types."""
