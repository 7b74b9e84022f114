from wfviz.cli import main

main()
