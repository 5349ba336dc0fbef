"""Scene file formats (informative): reading and writing the files 3DGS users exchange.

Every reader returns a validated ``lghcc.common.scene.GaussianScene`` (or raises InputError
naming the file and the problem); every writer writes atomically.
"""
