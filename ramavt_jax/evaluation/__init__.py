"""Evaluation layer: episode rollouts and summaries (``rollouts``), trained run folders as policies (``runs``), the
end-of-training evaluation of a run folder (``final``) and the paper's tables (``tables``).

Above the training layer (it reads run folders and checkpoints), below the figures and the command line.
"""
