"""A crashed campaign run says what crashed: an ExceptionGroup from a TaskGroup names each
sub-exception and where it was raised, not only "1 sub-exception"."""

from __future__ import annotations

import asyncio

from eaglemission.lab.campaign.campaign import crash_explanation


async def _fails_in_a_task_group() -> None:
    async def lost_link() -> None:
        raise ConnectionError("link to the vehicle lost")

    async with asyncio.TaskGroup() as tg:
        tg.create_task(lost_link())


def test_a_task_group_crash_names_its_sub_exception_and_where() -> None:
    try:
        asyncio.run(_fails_in_a_task_group())
    except BaseException as exc:  # noqa: BLE001 - the group is what a campaign run sees
        text = crash_explanation(exc)
    assert text.startswith("ConnectionError: link to the vehicle lost (")
    assert "test_campaign_crash.py:" in text and "in lost_link)" in text


def test_a_plain_exception_keeps_its_type_and_message() -> None:
    try:
        raise ValueError("bad frame")
    except ValueError as exc:
        assert crash_explanation(exc).startswith("ValueError: bad frame (")
