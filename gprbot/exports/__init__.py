"""Result files for CAD, GIS, spreadsheets and robotics tools: DXF, GeoJSON, CSV, MCAP; the site's georeference."""
