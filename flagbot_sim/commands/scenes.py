"""``flagbot scenes``: the built-in scenes, the effects, and every scene key with its unit and range."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("scenes", help="list built-in scenes and the scene keys with units and ranges")
    p.set_defaults(func=cmd_scenes)


def cmd_scenes(args) -> int:
    import dataclasses

    from ..fields import format_bounds
    from ..scene import EFFECTS, SECTIONS
    from ..scene_files import builtin_scenes
    print("built-in scenes:", ", ".join(builtin_scenes()))
    print("\neffects:")
    width = max(map(len, EFFECTS))
    for k, v in EFFECTS.items():
        print(f"  {k:{width}s}  {v}")
    rows = [("key", "default", "unit", "allowed", "meaning")]
    for s, cls in SECTIONS.items():
        for f in dataclasses.fields(cls):
            m = f.metadata
            default = f.default
            default = "[" + ", ".join(map(str, default)) + "]" if isinstance(default, tuple) else \
                (repr(default) if default == "" else str(default))
            if len(default) > 24:
                default = default[:21] + "..."
            rows.append((f"{s}.{f.name}", default, m["unit"] or "-", format_bounds(m) or "-", m["doc"]))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    print("\nkeys:")
    for r in rows:
        print("  " + "  ".join(c.ljust(w) for c, w in zip(r[:4], widths)) + "  " + r[4])
    return 0
