"""The closed loop (issue 22), one command: `python -m garage_exp.loop`.

Base data from a quasi-random sample of scenarios (rendered with dataset=true), a base detector D0 trained on it,
D0's failures found by a search against D0 itself, two fine-tuned arms with equal images and epochs (H: D0's
hard scenarios; R: as many frames drawn at random from the same space), both with the same replay of base data,
evaluated on held-out scenarios of a plan no training frame came from, and a second search against the fine-tuned
detectors. Each step is a command of the project (`python -m garage_exp -m hydra/sweeper=search ...`,
`python -m garage_exp.train ...`), run as a child process; a step whose result is on disk is not run again.
"""
