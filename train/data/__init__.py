"""Training and test data: ModelNet clouds and meshes (``modelnet``, ``meshio``, ``shapes``), the depth renderer
(``render``) and its keyed caches (``cache_io``, ``render_cache``), metric tabletop data (``tabletop``), objects
standing in a scene (``scene``), view augmentation (``augment``) and the datasets the trainer samples
(``datasets``)."""
