"""Files: atomic writes, avatar files, .ply export."""
