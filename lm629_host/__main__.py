from lm629_host.cli import main

main()
