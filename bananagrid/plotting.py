"""Pictures of rasters with matplotlib (an optional extra)."""
