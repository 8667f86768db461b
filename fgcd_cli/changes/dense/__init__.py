"""Dense, confidence-weighted refinement of a registration: the raw flow and its smooth fit."""
