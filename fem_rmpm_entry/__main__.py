"""``python -m fem_rmpm_entry ARGS``: the ``fem-rmpm`` command."""
import sys

from fem_rmpm_entry import main

sys.exit(main())
