"""The vocabulary every layer uses: errors, units, where the files are, the canonical tables, query files."""
