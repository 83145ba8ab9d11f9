"""File formats silfit reads and writes: one module per format (fits, images and masks, meshes, keypoints,
subjects, rigs, videos, whole-body keypoints, safe unpickling, size limits)."""
