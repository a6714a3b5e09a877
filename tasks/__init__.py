"""Task definitions, one module per task family, found through a registry by name."""
