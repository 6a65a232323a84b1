"""The chaos run: faults on purpose against the daemon and its simulated drives, while a client
flies paths and jobs, with invariants checked all along (`make chaos`; `python -m chaos` with
`tools/` on the path; `docs/chaos.md` describes it).

One worker process per drive family (ODrive, CiA 402) runs its own daemon (`cablebot run`, a
child process: it can be stopped, starved, limited, cut off and killed), and holds the test
equipment beside it: the simulated drives on the daemon's udp_multicast bus behind a faulty
link (`equipment.ChaosBus`: frames lost, corrupted, duplicated, a bus-off period), a tap that
hears every frame the daemon sends (`equipment.Tap`), a Zenoh client flying paths, the fault
injectors (`faults`) and the invariant checks (`checks`). `__main__` starts the workers, adds
up their reports and prints them.
"""
