"""The live web view of a mission (`--view`): its state, its HTTP server and page."""
