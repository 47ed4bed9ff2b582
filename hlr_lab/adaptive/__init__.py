"""``hlr-lab acquire --adaptive``: θc measured on the object, not guessed (docs/planning.md, "The closed
loop").

A plan is made for a guessed θc (the cone about the mirror direction inside which a pixel counts as a
highlight sample). :func:`~hlr_lab.adaptive.run.acquire_adaptive` photographs a pilot first — the plan's
own poses that put a highlight on every region once (:mod:`~hlr_lab.adaptive.pilot`) — fits each region's
lobe from it, takes the θc the fit chooses for that lobe (:mod:`~hlr_lab.adaptive.theta_c`), plans the
rest again per region with those θc, the pilot's poses counted, and photographs what the re-plan adds.
The session's journal keeps the pilot, each region's θc and the re-plan (:mod:`hlr_lab.session.stages`);
a stopped run resumes at the stage it stopped in.
"""
