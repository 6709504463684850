"""The script an export ships to register itself with a BOP toolkit clone (``register_bop_toolkit.py``).

The BOP toolkit (https://github.com/thodan/bop_toolkit) knows its datasets by name: object ids,
scene ids and image size in ``bop_toolkit_lib/dataset_params.py`` and the VSD tolerance per
dataset in ``scripts/eval_bop19_pose.py``; an unknown name is refused. The generated script adds
the export under :data:`evalkit.reports.bop.BOP_DATASET_NAME` to a clone the user names, by
inserting entries at anchors of the toolkit's source (checked with thodan/bop_toolkit cea62d6,
June 2026); it stops with a message when an anchor is missing (another toolkit version) and
does nothing twice. See docs/bop.md.
"""

from __future__ import annotations

TEMPLATE = '''"""Register this dockbench BOP export as dataset {name!r} in a BOP toolkit clone.

Usage: python register_bop_toolkit.py /path/to/bop_toolkit
(written by dockbench export-bop; see dockbench's docs/bop.md)
"""
import pathlib
import sys

NAME, OBJ_IDS, SCENE_IDS, IM_SIZE, DELTA = {name!r}, {obj_ids!r}, {scene_ids!r}, {im_size!r}, {delta!r}
TAG = "  # registered by dockbench"
EDITS = [   # (file, anchor, lines inserted before it)
    ("bop_toolkit_lib/dataset_params.py", '        "lm": list(range(1, 16)),\\n',
     ["        %r: %r," % (NAME, OBJ_IDS)]),
    ("bop_toolkit_lib/dataset_params.py", '        "lm": [3, 7, 10, 11],\\n',
     ["        %r: []," % (NAME,)]),
    ("bop_toolkit_lib/dataset_params.py", '    else:\\n        raise ValueError("Unknown BOP dataset ({{}}).".format(dataset_name))',
     ["    elif dataset_name == %r:" % (NAME,), '        p["scene_ids"] = %r' % (SCENE_IDS,),
      '        p["im_size"] = %r' % (IM_SIZE,)]),
    ("scripts/eval_bop19_pose.py", '                "hb": 15,\\n',
     ["                %r: %r," % (NAME, DELTA)]),
]


def main(root):
    texts = {{}}
    for rel, _, _ in EDITS:                      # an earlier registration's lines go first
        path = root / rel
        texts[path] = "".join(x for x in path.read_text().splitlines(True) if not x.rstrip().endswith(TAG.strip()))
    for rel, anchor, lines in EDITS:
        path = root / rel
        if texts[path].count(anchor) != 1:
            sys.exit(f"{{path}}: expected the text {{anchor!r}} once; another toolkit version? "
                     "Add the dataset by hand (dockbench docs/bop.md)")
        texts[path] = texts[path].replace(anchor, "".join(x + TAG + "\\n" for x in lines) + anchor, 1)
    for path, text in texts.items():
        path.write_text(text)
    print(f"{{root}}: dataset {{NAME!r}} registered (objects {{OBJ_IDS}}, scenes {{SCENE_IDS}}, size {{IM_SIZE}})")


if __name__ == "__main__":
    if len(sys.argv) != 2 or not (pathlib.Path(sys.argv[1]) / "bop_toolkit_lib").is_dir():
        sys.exit("usage: python register_bop_toolkit.py /path/to/bop_toolkit (a clone with bop_toolkit_lib/)")
    main(pathlib.Path(sys.argv[1]))
'''


def registration_script(
    name: str, obj_ids: list[int], scene_ids: list[int], width: int, height: int, delta_mm: float
) -> str:
    """The text of ``register_bop_toolkit.py`` for one export."""
    return TEMPLATE.format(
        name=name,
        obj_ids=list(obj_ids),
        scene_ids=list(scene_ids),
        im_size=(int(width), int(height)),
        delta=int(delta_mm) if float(delta_mm).is_integer() else float(delta_mm),
    )
