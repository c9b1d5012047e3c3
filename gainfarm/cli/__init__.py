"""What the three command lines (`worker`, `broker`, `analytic`) share: one error line and exit
status for bad input, the options several commands take, and scores printed for a person.

The edge of every role, so the only package besides schemas/ and models/ that worker/ and broker/
may import; it imports nothing of the project but schemas/.
"""
