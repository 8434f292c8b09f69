"""``python -m logiq_sql.cli``: the `logiq-sql` command."""

import sys

from logiq_sql.cli import main

sys.exit(main())
