from gtsweep.cli import main

main()
