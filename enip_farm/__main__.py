from enip_farm.cli import main

main()
