"""The closed loop (issues 22 and 39), one command: `python -m garage_exp.loop`.

D0 is a COCO-pretrained detector; base data from a quasi-random sample of the space on the training plans gives the
replay and the validation scenarios. In each of `rounds` rounds, each arm's generator (R: random scenarios, T: TPE
failures, Q: the archive's failures) searches the arm's detector of the round before; what it finds joins the arm's
suite, and that detector is fine-tuned on it with replay, every arm at the same budget, for each training seed.
Every detector is scored on held-out suites: the failure rate on a fixed quasi-random sample of the space on a plan
no training frame came from, an easy suite, the protocol cases and real photos. Each step is a command of the
project (`python -m garage_exp -m hydra/sweeper=search ...`, `python -m garage_exp.train ...`,
`python -m garage_exp.verify ...`), run as a child process; a step whose result is on disk is not run again.
"""
