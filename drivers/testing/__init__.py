"""Protocol emulators standing in for real controllers in tests: GRBL on a pty, a fake UR."""
