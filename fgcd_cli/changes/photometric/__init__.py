"""Photometric stereo for change cues: the stack, the light basis, relief apart from colour."""
