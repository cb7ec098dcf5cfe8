"""File formats the offline tools read and write: frames files and area-graph files."""
