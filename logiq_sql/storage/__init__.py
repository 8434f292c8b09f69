"""The DuckDB file and the Parquet dataset: tables, connections, the publish protocol, one writer at a time."""
