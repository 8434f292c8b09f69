"""logiq_sql."""
