"""``python -m magwarp ...`` is the ``magwarp`` command."""

from magwarp.cli import main

raise SystemExit(main())
