"""The README's Python example runs as written."""

import pathlib
import re

import numpy as np

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"


def test_readme_example_runs():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "README has no python example"
    namespace = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)
    assert namespace["traj"].y.shape == (101, 3, 6)
    assert namespace["heights"].shape == (8,)
    assert namespace["dz_dk"].shape == (2, 6)


def test_readme_scenario_example_is_the_packaged_default():
    import tomllib

    from elasticoop._config import build_scenario

    text = README.read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, flags=re.S)
    assert blocks, "README has no scenario example"
    packaged = README.parent / "elasticoop" / "scenarios" / "beam_lift.toml"
    assert blocks[0] == packaged.read_text()
    scenario = build_scenario(tomllib.loads(blocks[0]), "README.md")
    assert scenario.body_names == ("beam", "left", "right")


def test_readme_images_and_commands_exist():
    from elasticoop._cli import build_parser

    text = README.read_text()
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert images and all((README.parent / image).is_file() for image in images)
    shell = "".join(re.findall(r"```bash\n(.*?)```", text, flags=re.S))
    commands = set(re.findall(r"^elasticoop (\w+)", shell, flags=re.M))
    known = set(build_parser()._subparsers._group_actions[0].choices)
    assert commands and commands <= known


def test_readme_analysis_example_runs():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    (block,) = [b for b in blocks if "static_equilibrium" in b]
    namespace = {}
    exec(compile(block, "README.md", "exec"), namespace)
    assert namespace["traj"].reaction.shape == (51, 3, 6)
    split = namespace["split"]
    np.testing.assert_allclose(split.motion + split.internal, namespace["wrenches"])
    assert np.all(np.diff(namespace["modes"].frequencies) >= 0)
