"""What the `gprbot` commands do: the demos, replay, interpreting a file (entry points over the packages)."""
