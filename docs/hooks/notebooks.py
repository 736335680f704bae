"""MkDocs hook: the notebooks live in `notebooks/` beside `docs/`, where the tests
execute them; this adds each `notebooks/*.ipynb` to the site's files as
`notebooks/<name>.ipynb`, before mkdocs-jupyter turns them into pages."""

import pathlib

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files

NOTEBOOKS = pathlib.Path(__file__).resolve().parents[2] / "notebooks"


@event_priority(100)  # before mkdocs-jupyter's `on_files` (default priority 0)
def on_files(files: Files, config) -> Files:
    for path in sorted(NOTEBOOKS.glob("*.ipynb")):
        files.append(
            File(
                f"notebooks/{path.name}",
                src_dir=str(NOTEBOOKS.parent),
                dest_dir=config["site_dir"],
                use_directory_urls=config["use_directory_urls"],
            )
        )
    return files
