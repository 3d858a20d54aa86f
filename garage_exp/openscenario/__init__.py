"""OpenSCENARIO and OpenDRIVE out and in (docs/openscenario.md), in one package: the schemas (asam.py), the
writers (lanes.py the plan's roads, xodr_write.py the OpenDRIVE file, xosc_write.py the OpenSCENARIO file,
v1_0.py what OpenSCENARIO 1.0 for CARLA's ScenarioRunner wants, export.py one export's files, tracks.py a job's
shots as the actors' tracks, model.py what they share), the `export` node's schema and checks (checks.py), and the
readers (xodr_read.py, xosc_params.py, xosc_read.py) under the importer (xosc_import.py, the command
`python -m garage_exp.scenario.import`)."""
