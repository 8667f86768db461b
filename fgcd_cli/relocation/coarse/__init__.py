"""The active coarse stage (paper 001, AccurateACL): camera and scene uncertainty bring a far start into rACR's basin."""
