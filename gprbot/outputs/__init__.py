"""What a run leaves for its user: PLY clouds, pipes.json, DXF/GeoJSON/CSV, pictures, report.html (atomic writes)."""
