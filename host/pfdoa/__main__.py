from pfdoa.cli import main

raise SystemExit(main())
