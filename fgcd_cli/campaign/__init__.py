"""Campaign, station and observation: the on-disk format with atomic writes and checksums."""
