"""Scale-aware point cloud alignment (rACR §3.4): fast (robust ICP + scale) and fine
(geometric + photometric) registration of the current cloud to the reference cloud.
"""
