# Sphinx configuration of motion_ctrl's documentation: Markdown pages (MyST) in this folder.
#
# Laid out as rosdoc2 expects of a ROS 2 package (a Sphinx project in doc/, conf.py beside
# index.md), so a ROS build farm renders it too; rosdoc2 then adds its own theme and extensions.
# Build it locally with scripts/docs (warnings are errors, as test/docs/test_docs.py builds it).
project = 'motion_ctrl'
author = 'motion_ctrl developers'
copyright = 'motion_ctrl developers, Apache-2.0'

extensions = ['myst_parser']
source_suffix = {'.md': 'markdown'}
root_doc = 'index'
exclude_patterns = ['_build']

# Links between pages may name a section: [text](page.md#section-title) for headings down to
# level 3. A link to a page, a section or a file that does not exist is a warning, and the
# test's build (-W) fails on it; so does an unknown reference (nitpicky).
myst_heading_anchors = 3
nitpicky = True

html_theme = 'alabaster'
html_theme_options = {'page_width': '1200px', 'sidebar_width': '260px'}
html_title = 'motion_ctrl documentation'
html_show_sourcelink = False
