"""Where the project meets the outside world, shared by every process: the network and the disk.

- `transport`: Zenoh sessions as the farm opens them (explicit endpoints, the secure profile).
- `ask`: a question to the broker that hears only the broker's answer.
- `files`: files written whole or not at all, leftovers of killed writes, a directory's lock.

Above the contract (`gainfarm.schemas`, which says what crosses these edges and runs no I/O of
its own) and the robot (`gainfarm.models`); below the command lines and the processes.
"""
