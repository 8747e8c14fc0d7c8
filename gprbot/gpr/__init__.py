"""GPR signal processing, classical interpretation and file formats (pure numpy, no I/O but files)."""
