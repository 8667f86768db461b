"""The image stage: the last millimetres measured on the reference images, with their own checks and uncertainty."""
