"""Registration of cross-sections in 3D, completion into dense clouds, model sessions, output files."""
