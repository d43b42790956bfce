from dockingrl.cli import main

raise SystemExit(main())
