"""Grid files shipped with dockingrl (see :func:`dockingrl.grid.load_grid`)."""
