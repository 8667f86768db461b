"""Per-pixel change cues and the relief / colour label of each region."""
