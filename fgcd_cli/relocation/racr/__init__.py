"""The 3D rACR stage (paper 000, Fig. 2): align the VSE cloud to the reference, adjust by Eq. 3."""
