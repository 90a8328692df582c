"""Print the node's parameters as a Markdown table (for the README), from their descriptors.

Usage: ``python tools/param_table.py [--output FILE]``. The table is generated from
``obstacle_detection.ros_params`` (itself built from DetectorParams' field metadata), so it
cannot drift from what the node declares. Columns: the ROS name, type, the default (seed Table
4.2 for the pipeline), the Table 4.3 value where it differs (``params/corridor_video.yaml``), the
allowed range, and the description.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from obstacle_detection.params import table_4_3
from obstacle_detection.ros_params import ALL_PARAMS, ParamSpec, pipeline_params_to_ros

HEADER = ('| Parameter | Type | Default (Table 4.2) | Table 4.3 | Range | Description |\n'
          '| --- | --- | --- | --- | --- | --- |')


def _format_value(value: object) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return f'{value:g}'
    if isinstance(value, str):
        return f'`{value}`'
    return str(value)


def _row(spec: ParamSpec, video: dict[str, object]) -> str:
    other = video.get(spec.name, spec.default)
    other_text = _format_value(other) if other != spec.default else ''
    range_text = spec.range_text
    if spec.read_only:
        range_text = (range_text + ' ' if range_text else '') + 'read-only'
    description = spec.description.replace('|', '\\|')
    return (f'| `{spec.name}` | {spec.type_name} | {_format_value(spec.default)} | '
            f'{other_text} | {range_text} | {description} |')


def parameter_table() -> str:
    """Return the Markdown table of every ROS parameter of the node, one row each."""
    video = pipeline_params_to_ros(table_4_3())
    return '\n'.join([HEADER, *(_row(spec, video) for spec in ALL_PARAMS)]) + '\n'


def main(argv: list[str] | None = None) -> int:
    """Command-line entry: print the table or write it to ``--output``; returns 0."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--output', type=Path, help='write the table here instead of stdout')
    args = parser.parse_args(argv)
    table = parameter_table()
    if args.output is None:
        sys.stdout.write(table)
    else:
        args.output.write_text(table, encoding='utf-8')
    return 0


if __name__ == '__main__':
    sys.exit(main())
