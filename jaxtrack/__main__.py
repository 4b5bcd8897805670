import sys

from jaxtrack.cli import main

sys.exit(main())
