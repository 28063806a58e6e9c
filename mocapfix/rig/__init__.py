"""How a rig is understood: which joint of any humanoid skeleton plays which body part, and
the mapping of a recording's joints onto a model's.

Read in this order:
- structure.py: the body parts from the rig's tree and motion, in numbered steps (extremities;
  head, hands and feet; hips; legs and arms; spine; neck and head; sides), over tree.py (the
  joint tree, its leaves' groups and branches, what is measured over the frames);
- names.py: what a joint's name says (its side: the one reading of a side from a name; its part);
- labels.py: the two put together, one label per joint; the pelvis and the limb groups from them;
- mapping.py: a recording's joints onto a model's (the canonical body, core/skeleton.py body21).

numpy only; imports core/ and nothing above it. io/ uses it while reading (a file's unit and up
axis come from the legs and the trunk).
"""
