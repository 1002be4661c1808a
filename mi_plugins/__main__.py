from mi_plugins.app.cli import main

raise SystemExit(main())
