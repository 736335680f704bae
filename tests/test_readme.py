"""The README and the Python guide (docs/guide.md) are executed: the README's
example is the guide's first block, and every ```python block of the guide runs, in
order, in one namespace (as a reader pasting them into one Python session would),
each block's result checked. The README keeps its promises: its size, its set-up
commands (CI runs the test command), its links and the commands it names."""

import contextlib
import pathlib
import re

import jax
import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GUIDE = ROOT / "docs" / "guide.md"
FENCE = re.compile(r"^ *```(\w*)\n(.*?)^ *```", flags=re.S | re.M)
# The README stays a front door: pitch, set-up, one example, links.
MAX_README_BYTES = 8 * 1024

# One marker per python block of the guide, in order: a string only that block
# contains.
MARKERS = {
    "first": "eo.MobileModel([beam, grasp, grasp], grasps)",
    "gradient": "jax.grad(final_height)",
    "analysis": "eo.static_equilibrium(model, y0, held)",
    "study": "mc.run_study(study",
    "sensitivities": "mc.local_sensitivities(study",
    "identification": "eo.identify(model, [experiment], where)",
}
# The earlier blocks each block uses (the guide says which example continues
# which). Blocks run in order in one namespace, as in a reader's session; a block
# no later one needs (the gradient, slow to compile) may be left out.
NEEDS = {
    "first": (),
    "gradient": ("first",),
    "analysis": ("first",),
    "study": ("first",),
    "sensitivities": ("first", "study"),
    "identification": ("first",),
}


def _fences(text: str) -> list[tuple[str, int, str]]:
    """(language, line of the first code line (0-based), code) of every fenced
    block, in order."""
    return [
        (m.group(1), text.count("\n", 0, m.start(2)), m.group(2))
        for m in FENCE.finditer(text)
    ]


def _python_blocks(path: pathlib.Path = GUIDE) -> list[tuple[int, str]]:
    return [
        (line, code)
        for lang, line, code in _fences(path.read_text())
        if lang == "python"
    ]


class _Session:
    """The guide's python blocks, run in order in one namespace, in a folder of
    their own (the Monte Carlo example writes a store)."""

    def __init__(self, folder: pathlib.Path):
        self.folder = folder
        self.namespace: dict = {"__name__": "readme"}
        self.done: list[str] = []
        self.failed: set[str] = set()

    def run(self, name: str) -> dict:
        """Run block `name` and the blocks it needs that have not run yet."""
        order = list(MARKERS)
        blocks = dict(zip(order, _python_blocks(), strict=True))
        needed = {name, *NEEDS[name]}
        if needed & self.failed:
            pytest.fail(f"the guide's {sorted(needed & self.failed)} block failed")
        todo = sorted(needed - set(self.done), key=order.index)
        with contextlib.chdir(self.folder):
            for block in todo:
                later = [b for b in self.done if order.index(b) > order.index(block)]
                assert not later, f"{block!r} would run after {later}"
                line, code = blocks[block]
                # padded so that tracebacks give the guide's line numbers
                source = compile("\n" * line + code, str(GUIDE), "exec")
                try:
                    exec(source, self.namespace)
                except BaseException:
                    self.failed.add(block)
                    raise
                self.done.append(block)
        return self.namespace


@pytest.fixture(scope="module")
def readme(tmp_path_factory):
    return _Session(tmp_path_factory.mktemp("readme"))


def test_every_python_block_is_checked():
    for path in (README, GUIDE):
        languages = {lang for lang, _, _ in _fences(path.read_text())}
        # an unlabelled fence would hide code from these tests
        assert languages <= {"python", "bash", "toml"}, (path.name, languages)
    blocks = [code for _, code in _python_blocks()]
    owners = [[name for name, m in MARKERS.items() if m in code] for code in blocks]
    assert owners == [[name] for name in MARKERS], owners
    # the README's one example is the guide's first
    assert [code for _, code in _python_blocks(README)] == blocks[:1]


def test_first_simulation(readme):
    ns = readme.run("first")
    traj = ns["traj"]
    assert traj.y.shape == (101, 3, 6)
    assert traj.elastic_wrench().shape == (101, 2, 6)
    assert int(traj.status) == 0
    # the energy balance closes to the solver's tolerance (J; weights ~ 25 N)
    assert abs(float(traj.energy_residual()[-1])) < 1e-4
    # each grasp stays on its side of the beam (there is no contact model) ...
    y = np.asarray(traj.y)
    assert np.all(y[:, 1, 0] < y[:, 0, 0]) and np.all(y[:, 2, 0] > y[:, 0, 0])
    # ... and the three rise together: 2 N over 2.6 kg for 1 s, z = a t^2 / 2
    rise = y[-1, :, 2] - y[0, :, 2]
    np.testing.assert_allclose(rise, 0.5 * 2.0 / 2.6, rtol=0.05)


@pytest.mark.slow
def test_batch_and_gradient(readme):
    ns = readme.run("gradient")
    heights, dz_dk, stiffness = ns["heights"], ns["dz_dk"], ns["model"].stiffness
    assert heights.shape == (8,) and np.all(np.isfinite(heights))
    assert dz_dk.shape == stiffness.shape == (2, 6)
    # the gradient agrees with the batch: d height / d scale at scale 1 against
    # the secant between the two scales around 1
    scale = np.linspace(0.5, 2, 8)
    secant = (heights[3] - heights[2]) / (scale[3] - scale[2])
    directional = np.sum(np.asarray(dz_dk) * np.asarray(stiffness))
    np.testing.assert_allclose(directional, secant, rtol=0.2)


@pytest.mark.slow
def test_analysis(readme):
    ns = readme.run("analysis")
    eq, driven, y0 = ns["eq"], ns["driven"], ns["y0"]
    # the grasps stay where they were; the beam sags, hanging in its links
    np.testing.assert_allclose(eq.y[1:], y0[1:])
    # the first simulation starts from this equilibrium, below the unloaded pose
    np.testing.assert_allclose(eq.y[0], y0[0], atol=1e-8)
    assert 0.0 < float(ns["rest"][0, 2] - eq.y[0, 2]) < 0.2
    assert driven.reaction.shape == (51, 3, 6)
    assert np.all(np.asarray(driven.reaction[:, 0]) == 0)  # the object is free
    # the drive does work, and the energy balance still closes
    work = float(np.max(np.abs(driven.work)))
    assert work > 0.1  # J: the grasps raise about 2.6 kg by some 7 cm
    assert abs(float(driven.energy_residual()[-1])) < 1e-6 * work
    split = ns["split"]
    np.testing.assert_allclose(split.motion + split.internal, ns["wrenches"])
    frequencies = np.asarray(ns["modes"].frequencies)
    assert frequencies.shape == (6,)  # the beam's 6 coordinates are free
    assert np.all(frequencies > 0) and np.all(np.diff(frequencies) >= 0)


@pytest.mark.slow
def test_monte_carlo_study(readme):
    ns = readme.run("study")
    mc, ds, study = ns["mc"], ns["ds"], ns["study"]
    n = study.n_samples
    assert mc.summary(ds)["n_succeeded"] == n
    assert ds["pose"].shape == (n, 21, 6)
    assert ds["peak_force"].shape == (n, 2)
    # Latin hypercube: each of the n strata of each entry is hit once
    load = np.asarray(ds["load"])[:, :, 2] / np.asarray(ns["lift"])[:, 2]
    strata = np.sort(np.floor((load - 0.8) / 0.4 * n), axis=0)
    np.testing.assert_array_equal(strata, np.arange(n)[:, None] * np.ones((1, 2)))
    p30 = ns["p30"]
    p = np.asarray(p30["probability"])
    assert np.all((p30["lower"] <= p) & (p <= p30["upper"]))
    np.testing.assert_allclose(p, np.mean(np.asarray(ds["peak_force"]) > 30.0, 0))
    # the store resumes: a second run simulates nothing and returns the same data
    again = mc.run_study(study, readme.folder / "study_dir", progress=False)
    np.testing.assert_array_equal(again["peak_force"], ds["peak_force"])
    assert (readme.folder / "study_dir" / "manifest.json").is_file()


@pytest.mark.slow
def test_monte_carlo_sensitivities(readme):
    ns = readme.run("sensitivities")
    ranking = ns["ranking"]
    share = np.asarray(ranking)
    assert np.all(np.diff(share) <= 0)
    np.testing.assert_allclose(share.sum(), 1.0)
    # the run starts from the nominal equilibrium, where grasp 1's link is
    # stretched by a fixed amount: its tension, and so its peak force, scales with
    # the link's stiffness along itself (x)
    assert str(ranking["parameter"][0].values) == "stiffness[0, 0]"
    linear, sampled = (
        ranking.attrs[k] for k in ("linearized_variance", "sample_variance")
    )
    assert 0.5 < linear / sampled < 2.0


@pytest.mark.slow
def test_identification(readme):
    ns = readme.run("identification")
    result, truth = ns["result"], ns["truth"]
    assert result.converged, result.reason
    leaves = lambda m: np.concatenate(  # noqa: E731
        [np.ravel(x) for x in jax.tree.leaves(ns["where"](m))]
    )
    exact = leaves(truth)
    stderr = np.concatenate([np.ravel(s) for s in jax.tree.leaves(result.stderr)])
    ok = result.identifiable
    # the guide's numbers: x and z of each link's stiffness and damping
    excited = np.zeros((2, 2, 6), bool)
    excited[:, :, [0, 2]] = True
    np.testing.assert_array_equal(ok, excited.ravel())
    error = np.abs(result.estimate - exact)
    assert np.all(error[ok] < 2.0 * stderr[ok])  # (the guide: within 2)
    relative = (error / exact).reshape(2, 2, 6)[:, :, [0, 2]]
    assert np.all(relative[0] < 0.003) and np.all(relative[1] < 0.08)
    # the guide's standard errors: stiffness 0.04 % (x) and 0.23 % (z), damping
    # 3 % (x) and 31 % (z, barely excited), relative to the estimates (the
    # report's column, which rounds 0.035 % to 0.04 %)
    spread = (stderr / result.estimate).reshape(2, 2, 6)[:, :, [0, 2]]
    np.testing.assert_allclose(spread[0], [[3.5e-4, 2.3e-3]] * 2, rtol=0.05)
    np.testing.assert_allclose(spread[1], [[0.0295, 0.31]] * 2, rtol=0.03)
    assert np.all(np.isinf(stderr[~ok]))
    assert "NOT IDENTIFIABLE" in result.report()
    # every parameter stays in the fit and every standard error is marginal: the
    # flagged entries are not held at a start value (which would make the others
    # look more certain than they are); their infinite standard errors say that
    # their values are not estimates
    assert not np.any(result.held)
    assert "marginal, NOT IDENTIFIABLE" in result.report()
    np.testing.assert_allclose(leaves(result.model), result.estimate)
    # and they keep the model's values (to the rounding of the fit's log
    # coordinates), not the equation-error start's fit to the noise
    start = leaves(ns["model"])
    np.testing.assert_allclose(result.estimate[~ok], start[~ok], rtol=1e-14)


def test_readme_is_short():
    assert len(README.read_bytes()) <= MAX_README_BYTES


def test_readme_links_and_commands_exist():
    from elasticoop._cli import COMMANDS

    text = README.read_text()
    links = re.findall(r"\]\(((?!https?:)[^)#]+)(?:#[^)]*)?\)", text)
    assert links and all((ROOT / link).exists() for link in links), links
    shell = "".join(code for lang, _, code in _fences(text) if lang == "bash")
    commands = set(re.findall(r"^ *elasticoop (\w+)", shell, flags=re.M))
    commands |= set(re.findall(r"`elasticoop (\w+)", text))  # in the text
    assert commands <= set(COMMANDS), commands - set(COMMANDS)


def test_readme_set_up_commands():
    """The README opens with two commands: install and run the main job, install
    and run the fast tier of the tests. CI takes the test command from the first
    line that mentions pytest, and then runs the slow tier, `-m slow`: together
    they run every test once."""
    text = README.read_text()
    lang, line, code = _fences(text)[0]
    assert lang == "bash" and line < 20
    first, second = code.splitlines()
    assert first.endswith("pip install . && python -m elasticoop")
    pytest_line = next(x for x in text.splitlines() if "pytest" in x)
    assert pytest_line == second
    assert second.endswith(
        'pip install -e ".[test]" && pytest -n auto -q -m "not slow"'
    )
    ci = (ROOT / ".ci" / "run").read_text()
    assert "grep -m1 'pytest' README.md" in ci and "-m slow" in ci
