"""Source formats read into the canonical tables (one reader per format), checked and localised on lanes."""
