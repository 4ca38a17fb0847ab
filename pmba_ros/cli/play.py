# Copyright 2026 pmba_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""``pmba play``: publish a recording into a live ROS 2 graph with its recorded timing.

For users with rclpy from pip (``pip install .[ros]``) but no ``ros2 bag``::

    pmba play street_bag                          # all topics, real time
    pmba play street_bag --rate 2 --topics /features /keyframe_pose /camera_info
    pmba play street_bag --clock                  # /clock for nodes with use_sim_time
    pmba play street_bag --remap /features:=/feature_tracker/feature
    pmba play street_bag --topics /features /keyframe_pose --wait-for-subscribers 30
    pmba play street_bag --loop --clock           # again and again, until Ctrl-C

Messages are published as stored (CDR), reliable and transient local: a subscriber that is
transient local too (``features_qos:=transient_local`` on pmba_node) loses none of the first
messages to discovery. ROS 1 bags must be converted first (``rosbags-convert``).
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import TYPE_CHECKING

from pmba_ros.errors import BagError

if TYPE_CHECKING:
    import argparse


def _positive(text: str) -> float:
    import argparse

    try:
        value = float(text)
    except ValueError:
        value = float('nan')
    if not value > 0 or value == float('inf'):
        msg = f'expected a positive number, got {text!r}'
        raise argparse.ArgumentTypeError(msg)
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare the arguments of the ``play`` verb.

    Args:
        parser: Parser (or subparser) to add the arguments to.
    """
    parser.add_argument('bag', type=Path, help='rosbag2 folder or .mcap / .db3 file')
    parser.add_argument('--rate', type=_positive, default=1.0, metavar='R',
                        help='playback speed factor')
    parser.add_argument('--topics', nargs='+', metavar='TOPIC',
                        help='topics to play (default: all)')
    parser.add_argument('--clock', action='store_true',
                        help='publish /clock from the recording (for use_sim_time)')
    parser.add_argument('--delay', type=float, default=0.5, metavar='S',
                        help='seconds between creating the publishers and the first message '
                             '(lets subscribers discover them)')
    parser.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='S',
                        help='then wait up to S seconds until every played topic has a '
                             'subscriber')
    parser.add_argument('--remap', action='append', default=[], metavar='FROM:=TO',
                        help='remap a topic (repeatable)')
    parser.add_argument('--loop', action='store_true',
                        help='play the recording again from its start each time it ends, '
                             'until interrupted (pmba_node starts over on each pass)')


def run(args: argparse.Namespace) -> int:
    """Play the recording.

    Returns:
        0 when every message was published (or playback was interrupted).

    Raises:
        BagError: If the bag is missing or unreadable, or a requested topic is not in it.
        MessageError: If a message type is not available to rclpy.
    """
    from pmba_ros.io.bags import open_bags, serialized_messages
    from pmba_ros.node import play_messages

    with open_bags([args.bag]) as bags:   # once: a damaged recording is salvaged once
        topics = bags.topics
        if args.topics:
            missing = sorted(set(args.topics) - set(topics))
            if missing:
                msg = (f'{args.bag}: topic(s) {", ".join(missing)} not in the bag (topics: '
                       f'{", ".join(sorted(topics))})')
                raise BagError(msg)
        wanted = sorted(args.topics or topics)
        bad = [r for r in args.remap if ':=' not in r]
        if bad:
            msg = f'--remap {bad[0]!r}: expected FROM:=TO'
            raise BagError(msg)
        ros_args = ['--ros-args', *[a for r in args.remap for a in ('-r', r)]]
        passes = itertools.count() if args.loop else range(1)
        messages = itertools.chain.from_iterable(serialized_messages(bags, wanted)
                                                 for _ in passes)
        count = play_messages(messages,
                              {t: topics[t].msgtype for t in wanted}, rate=args.rate,
                              clock=args.clock, delay_s=max(0.0, args.delay),
                              wait_for_subscribers_s=max(0.0, args.wait_for_subscribers),
                              ros_args=ros_args)
    print(f'played {count} messages on {len(wanted)} topics')
    return 0
