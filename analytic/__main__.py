from analytic.cli import main

main()
