"""Scenarios (issue 28, item 3): a cell's test case as a timeline of steps (faults on devices or
groups, stimuli, waits) and expectations, parsed and checked before anything runs (parse.py), run by
a scheduler that is given the time (schedule.py, run.py) and judged from what the devices recorded
(verdict.py)."""
