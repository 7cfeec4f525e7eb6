import sys

from lightemma.cli import main

sys.exit(main())
