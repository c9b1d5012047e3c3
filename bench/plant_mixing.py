"""What mixing plants costs a learned model: identification on one plant's episodes or on all.

    python bench/plant_mixing.py DATASET

A dataset of several plants (`analytic dataset --plants K`, or robust runs' own tuning episodes,
which ran on their variants) asks a model of (q, q̇, q̈) for one arm's dynamics where there are
several. This scores, on the test episodes of the dataset's most common plant only: that
plant's own dynamics (the floor), the consistent linear identification fitted on that plant's
train episodes, and the same fitted on every train episode, train_variants' too (what
`learning.benchmark` did before a dataset kept one plant per split, version 5).
"""

import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from gainfarm.analytic.data import learning
from gainfarm.models.dynamics import DynamicsModel, true_model
from gainfarm.schemas.robot import PlantSpec


def main(dataset: Path) -> None:
    splits = learning.read_splits(dataset)
    for name in ("train", "test"):  # every episode, whatever its plant
        variants = learning.read_split(dataset, f"{name}_variants")
        splits[name] = learning.Rows.concatenate([splits[name], variants])
    table = pq.read_table(dataset / "episodes.parquet", columns=["episode_id", "model"]).to_pydict()
    counts = Counter(table["model"])
    text, _ = counts.most_common(1)[0]
    plant = PlantSpec.model_validate_json(text)
    mine = [e for e, m in zip(table["episode_id"], table["model"], strict=True) if m == text]
    train, test = (
        splits[name].take(np.isin(splits[name].episode_id, mine)) for name in ("train", "test")
    )
    prior = learning.rigid_prior(plant)
    models = {}
    for name, rows in (("alone", train), ("mixed", splits["train"])):
        parameters, _, _ = learning.identify(prior.spec, rows)
        models[name] = DynamicsModel("linear", "inverse", prior.spec, parameters=parameters)
    print(
        f"{len(counts)} plants; the most common's {len(mine)} episodes: {len(train):,} train "
        f"rows, {len(test):,} test rows"
    )
    for name, model in (
        ("its own dynamics (floor)", true_model(plant)),
        ("linear, fitted on its train episodes", models["alone"]),
        ("linear, fitted on every train episode", models["mixed"]),
    ):
        print(f"{name}: test nMSE {learning.score_rows(model, test, train)['nmse_mean']:.5f}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__.splitlines()[2].strip())
    main(Path(sys.argv[1]))
