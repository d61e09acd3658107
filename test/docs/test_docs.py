"""The documentation: README.md (the landing page) and the site in doc/ (Sphinx with MyST
Markdown, laid out as rosdoc2 builds a ROS package's doc/).

The site builds with warnings as errors, nitpicky, as `scripts/docs` builds it: a link to a page,
a section or a picture that does not exist, an unknown reference or a page in no table of
contents fails the build. The tiny sites built in tmp_path show that the build does fail on
each kind (and builds a good one). The parameters page is what the register table generates
(test_registers checks every generated block; here, that a page that differs is caught).
Nothing a user reads points outside the repository.

In-process (Sphinx is plain Python): no ROS, no process.
"""
import pathlib
import re
import shutil

import pytest
from sphinx.cmd.build import build_main

from motion_ctrl.core import registers as R

REPO = pathlib.Path(__file__).resolve().parents[2]
DOC = REPO / 'doc'
# As scripts/docs and a build farm's strict build: warnings are errors, all of them reported.
STRICT = ['-W', '--keep-going', '-n', '-q', '-b', 'html']
# myst-parser 5.2 still reads an attribute Sphinx 9 deprecates: not ours to fix.
pytestmark = pytest.mark.filterwarnings('ignore::sphinx.deprecation.RemovedInSphinx11Warning')


def build(src: pathlib.Path, out: pathlib.Path, capsys) -> tuple[int, str]:
    """sphinx-build STRICT src out, in this process: its exit code and its warnings."""
    capsys.readouterr()
    code = build_main([*STRICT, str(src), str(out)])
    return code, capsys.readouterr().err


@pytest.mark.core_slow
def test_the_documentation_builds_without_a_warning(tmp_path, capsys):
    code, err = build(DOC, tmp_path / 'html', capsys)
    assert code == 0, f'the documentation does not build cleanly (scripts/docs):\n{err}'
    index = (tmp_path / 'html' / 'index.html').read_text()
    for page in sorted(DOC.glob('*.md')):
        assert (tmp_path / 'html' / f'{page.stem}.html').exists(), page.name
        if page.stem != 'index':
            assert f'href="{page.stem}.html"' in index, f'{page.name} is not linked from index'


# A site of two pages with the project's own conf.py; `{page}` is the second page's text.
GOOD = ('See [the index](index.md), [its section](index.md#a-section) and '
        '[this one](#further-down).\n\n## Further down\n')
BROKEN = {
    'a link to a page that does not exist': ('[the tuning guide](tuning_guide.md)',
                                             'tuning_guide.md'),
    'a link to a section that does not exist': ('[units](index.md#units)', 'units'),
    'an unknown reference': ('{ref}`the-servo-bus`', 'the-servo-bus'),
    'a picture that does not exist': ('![the demo](demo.png)', 'demo.png'),
}


def tiny_site(root: pathlib.Path, page: str) -> pathlib.Path:
    root.mkdir()
    shutil.copy(DOC / 'conf.py', root / 'conf.py')
    (root / 'index.md').write_text('# Tiny\n\n## A section\n\n```{toctree}\npage\n```\n')
    (root / 'page.md').write_text(f'# Page\n\n{page}\n')
    return root


@pytest.mark.core_slow
def test_a_good_tiny_site_builds(tmp_path, capsys):
    code, err = build(tiny_site(tmp_path / 'src', GOOD), tmp_path / 'html', capsys)
    assert code == 0, err


@pytest.mark.core_slow
@pytest.mark.parametrize('kind', sorted(BROKEN))
def test_the_build_fails_on(kind, tmp_path, capsys):
    text, named = BROKEN[kind]
    code, err = build(tiny_site(tmp_path / 'src', f'{GOOD}\n{text}\n'), tmp_path / 'html', capsys)
    assert code != 0, f'{kind} built without a warning'
    assert 'page.md' in err and named in err, err


def test_a_parameters_page_that_differs_from_the_register_table_is_caught():
    blocks = R.DOC_BLOCKS['doc/parameters.md']
    text = (DOC / 'parameters.md').read_text()
    assert R.stale_blocks(text, blocks) == []
    kp = next(line for line in text.splitlines() if line.startswith('| `kp` |'))
    assert R.stale_blocks(text.replace(kp, kp.replace('| 16000 |', '| 12000 |')
                                       .replace('Proportional', 'Integral')),
                          blocks) == ['registers:controller']
    lead = next(line for line in text.splitlines() if line.startswith('| `lead` |'))
    assert R.stale_blocks(text.replace(lead + '\n', ''), blocks) == ['registers:plant']


def user_pages():
    return [REPO / 'README.md', *sorted(DOC.glob('*.md'))]


@pytest.mark.parametrize('page', user_pages(), ids=lambda p: p.name)
def test_nothing_a_user_reads_points_outside_the_repository(page):
    text = page.read_text()
    for outside in ('../shared', 'shared/', 'SPEC.md', 'REFERENCE.md', 'seeds/'):
        assert outside not in text, f'{page.name} names {outside}'
    if page.name != 'README.md':        # the site stands alone: no "README, Notes" left over
        assert 'README' not in text, f'{page.name} sends its reader to README'
    for target in re.findall(r'\]\(([^)\s]+)\)', text):
        if re.match(r'[a-z]+://', target) or target.startswith('#'):
            continue
        path = (page.parent / target.split('#')[0]).resolve()
        assert path.is_relative_to(REPO), f'{page.name} links outside the repository: {target}'


def test_readme_links_into_the_docs_exist_and_say_the_commands():
    text = (REPO / 'README.md').read_text()
    targets = [t for t in re.findall(r'\]\(([^)\s]+)\)', text) if not re.match(r'[a-z]+://', t)]
    assert any(t.startswith('doc/') for t in targets)
    for target in targets:
        assert (REPO / target.split('#')[0]).exists(), f'README links to {target}: no such file'
    # .ci/run runs the test command README gives; the demo and the docs build are README's too.
    for command in ('scripts/test', 'scripts/demo', 'scripts/docs'):
        assert f'\n{command}' in text, f'README does not give `{command}`'
    assert sum(1 for _ in text.splitlines()) <= 250, 'README is a landing page: at most 250 lines'
