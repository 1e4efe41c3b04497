"""Named, frozen, validated configurations (presets)."""
