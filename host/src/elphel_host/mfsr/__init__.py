"""mfsr."""
