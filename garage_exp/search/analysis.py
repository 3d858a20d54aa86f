# TEMPORARY (not committed): the helper writes the real one
from pathlib import Path
def analyse(study, out_dir, top=5):
    out_dir = Path(out_dir); out_dir.mkdir(parents=True, exist_ok=True)
    p = out_dir / "trials.csv"; study.trials_dataframe().to_csv(p, index=False); return [p]
