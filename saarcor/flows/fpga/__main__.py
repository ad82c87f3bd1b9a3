from saarcor.flows.fpga.flow import main

main()
