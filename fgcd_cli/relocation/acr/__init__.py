"""The ACR baseline (Tian et al., reference [1] of paper 000): 2D relative pose and bisection on the scale."""
