"""rACR relocation: the adjustment formula, the VSE session, the parallel loop, capture and revisit."""
