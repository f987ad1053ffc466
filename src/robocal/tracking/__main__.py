"""``python -m robocal.tracking flush | ui-url | ui`` (:func:`robocal.tracking.command.main`)."""

import sys

from robocal.tracking.command import main

sys.exit(main())
