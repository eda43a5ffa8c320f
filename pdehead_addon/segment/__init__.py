"""Step 2: the 3-D Chan-Vese soft segmentation of the head (eq. 16-21) and its clean-up.

Modules:

- :mod:`.binary_morphology`  Binary morphology on rows packed 64 voxels to a machine word (numpy only)
- :mod:`.chan_vese`          The 3-D Chan-Vese soft model (paper eq. 16-21) solved with Chambolle's dual projection
- :mod:`.chan_vese_band`     The full-resolution Chan-Vese level in a band of coarse blocks around the coarse boundary
- :mod:`.chan_vese_pyramid`  The 3-D Chan-Vese soft model (paper eq. 16-21) coarse to fine
- :mod:`.coarse_blocks`      Blocks of a coarse grid: block means, block reductions on slabs, nearest resampling
- :mod:`.disk_morphology`    In-slice disk morphology with radii in mm, the largest component and hole filling
- :mod:`.mask_cleanup`       Clean-up of the thresholded membership: what the paper does after eq. 21, and more
- :mod:`.run_labels`         Connected components of boolean volumes on runs along x (numpy + scipy.sparse only)
- :mod:`.segmentation`       Step 2: head segmentation with the 3D Chan-Vese soft model (paper eq. 16-21) and clean-up
"""
