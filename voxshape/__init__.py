"""voxshape's services: each a pure core plus a thin bus adapter, started by `voxshape <name>`."""
