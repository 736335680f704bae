"""MkDocs hook: the notebooks live in `notebooks/` beside `docs/`, where the tests
execute them; this adds each `notebooks/*.ipynb` to the site's files as
`notebooks/<name>.ipynb`, before mkdocs-jupyter turns them into pages, and takes
the MathJax loader of nbconvert's template out of those pages (the site's own KaTeX
renders their maths, with no network)."""

import pathlib
import re

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


# nbconvert's template loads MathJax (from a CDN unless told otherwise) between
# these two comments.
MATHJAX = re.compile(
    r"<!-- Load mathjax -->.*?<!-- End of mathjax configuration -->", flags=re.S
)


def on_post_page(output: str, page, config) -> str:
    if page.file.src_uri.endswith(".ipynb"):
        output = MATHJAX.sub("", output)
    return output
