"""Evaluation layer: episode rollouts and summaries (``rollouts``; the compiled program that flies the episodes:
``episode_program``), trained run folders as policies (``runs``), the end-of-training evaluation of a run folder
(``final``), the paper's tables (``tables``: run; ``report``: Markdown and the files tables.md / results.json) and the
held-out return of every checkpoint of a run (``curve``).

Above the training layer (it reads run folders and checkpoints), below the figures and the command line.
"""
