"""The models: frozen, validated parameter objects behind one protocol
(:mod:`bananagrid.protocol`), one module per model family, and the registry of their scene
kinds (:mod:`bananagrid.models.registry`). The public names are exported by :mod:`bananagrid`."""
