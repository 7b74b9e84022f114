from wfviz.entry import main

main()
