"""lghcc.batch (informative): ``lghcc-batch``, sweeps of scenes x presets x rate lambdas on Ray
or in one process. sweep.py reads and checks the sweep file; work.py is the work itself as
plain functions (prepare a scene, run a cell: encode, decode, evaluate), which never import
Ray; runner.py runs them on Ray or serially (--local) and keeps the results; report.py writes
the table and the RD plots."""
