from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'abd_joint_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={package_name: ['scenes/*.yaml', 'robots/*.urdf', 'live/web/*.html',
                                'live/web/*.js', 'live/web/package*.json']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        (os.path.join('share', package_name), ['package.xml']),
        (os.path.join('share', package_name, 'launch'), glob('launch/*.py')),
        (os.path.join('share', package_name, 'config'), glob('config/*.yaml')),
        (os.path.join('share', package_name, 'scenes'),
         glob(os.path.join(package_name, 'scenes', '*.yaml'))),
        (os.path.join('share', package_name, 'robots'),
         glob(os.path.join(package_name, 'robots', '*.urdf'))),
    ],
    install_requires=['setuptools'],
    # `pip install '.[sweep]'`: the engine of the `sweep` command (requirements-sweep.txt)
    extras_require={'sweep': ['ray==2.60.0'], 'live': ['foxglove-sdk==0.30.3']},
    zip_safe=True,
    maintainer='abd_joint_sim maintainers',
    maintainer_email='maintainers@abd-joint-sim.example.org',
    description='Affine-body revolute-joint simulation as a ROS 2 node',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'sim_node = abd_joint_sim.ros.node:main',
            'run_headless = abd_joint_sim.tools.run_headless:main',
            'replay_check = abd_joint_sim.tools.replay_check:main',
            'bag_recover = abd_joint_sim.tools.bag_recover:main',
            'plot_bag = abd_joint_sim.tools.plot_bag:main',
            'replay_bag = abd_joint_sim.tools.replay_bag:main',
            'sweep = abd_joint_sim.tools.sweep:main',
        ],
    },
)
