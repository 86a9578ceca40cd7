from spikegyro.cli import main

main()
