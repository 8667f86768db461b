"""The parallel relocation loop (paper 000, Fig. 2): the VSE, alignment and adjustment threads and what they share."""
