"""The lowest layer: errors, seeds, config validation, names and the version, shared by every part."""
