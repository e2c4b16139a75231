"""Render the pictures of the synthetic products used in the README and docs/.

    python docs/make_pictures.py            # writes docs/images/*.png

Each product gets one picture of four instances (seed 1), front and top view,
in their body frame (stalk up), all at the same scale, plus one overview of the
five products. Takes about a minute on a 2-core machine.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hortishape.mesh import Mesh
from hortishape.render import render_grid
from hortishape.synth import PRODUCTS, make_population

COLOURS = {"apple": "#c8402a", "pepper": "#d8281c", "zucchini": "#2f6b1f", "pear": "#b5b83a", "banana": "#e8c020"}


def body_frame(inst) -> Mesh:
    """The instance's scan moved back to its body frame (stalk along +z)."""
    inv = np.linalg.inv(inst.pose)
    return Mesh(inst.mesh.vertices @ inv[:3, :3].T + inv[:3, 3], inst.mesh.faces)


def main(out: Path = Path(__file__).resolve().parent / "images") -> None:
    out.mkdir(parents=True, exist_ok=True)
    firsts = []
    for product in PRODUCTS:
        pop = make_population(product, 4, random_state=1, pose="random", n_vertices=60000)
        meshes = [body_frame(p) for p in pop]
        firsts.append(meshes[0])
        titles = [f"{p.name}\n{p.dimensions[0]:.0f} x {p.dimensions[1]:.0f} x {p.dimensions[2]:.0f} mm" for p in pop]
        render_grid(meshes, out / f"{product}.png", titles=titles, n_cols=4, views=("front", "top"),
                    color=COLOURS[product], cell_size=(300, 340))
        print("wrote", out / f"{product}.png")
    render_grid(firsts, out / "products.png", titles=list(PRODUCTS), n_cols=5, views=("iso",),
                color=[COLOURS[p] for p in PRODUCTS], cell_size=(260, 380))
    print("wrote", out / "products.png")


if __name__ == "__main__":
    main()
