"""motors."""
