"""Tools only the tests use (imported as `tools.X`, tests/ being on the path as for the other helpers here):
esmini.py replays an OpenSCENARIO export in esmini and reads back where it put everything; asam_qc.py runs ASAM's
Quality Checker bundles on an export."""
